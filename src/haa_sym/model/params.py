"""Actuator and controller parameters as validated data (Table 1 and Sec. 3 of the paper).

A parameter file (TOML, see ``model/hyq_haa.toml`` and docs/model.md, "Actuator files")
describes an actuator ([motor], [bodies.*], [couplings.*], [sensors]; the structure is a
:class:`haa_sym.model.actuator.Topology`, the values a :class:`Plant`), a ``[controller]`` table and
optional ``[configurations.<name>]`` tables overriding plant keys (the leg configurations of
Table 1). The legacy flat ``[plant]`` table is read as the HyQ topology. Loading validates
everything and raises :class:`ParameterError` naming the file, the section, the key, the value
and what is allowed; nothing is silently defaulted.

Validation lives here and only here: :class:`Plant`, :class:`Controller` and :class:`Params`
check themselves on construction (so ``dataclasses.replace`` cannot make an invalid object
either), and :func:`gain_array` is the one rule for the gain points every analysis takes
(P_gain, D_gain, beta, alpha).

Example
-------
>>> from haa_sym.model.params import load_params
>>> p = load_params("model/hyq_haa.toml")                       # doctest: +SKIP
>>> p.configuration("retracted").plant.J_L2                     # doctest: +SKIP
0.129
"""
from __future__ import annotations

import gc
import math
import os
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Mapping

import numpy as np

from haa_sym.errors import ParameterError
from haa_sym.io.inputs import read_bytes
from haa_sym.model.actuator import (ACTUATOR_SECTIONS, HYQ, Actuator, Topology, check_keys, entry_values,
                              parse_actuator)
from haa_sym.model.motor import MOTOR_CONVENTION_DEFAULT, split_convention
from haa_sym.model import filters, structures
from haa_sym.model.filters import PARAMETERS as FILTER_PARAMETERS
from haa_sym.model.drive import DRIVE_KEYS, DRIVE_UNITS, Drive, drive_allowed, parse_drive
from haa_sym.model.limits import Limits, parse_limits
from haa_sym.model.resources import data_dir
from haa_sym.model.units import CONTROLLER_UNITS, check_number

__all__ = [
    "ParameterError",
    "Plant",
    "Controller",
    "Params",
    "CONTROLLER_KEYS",
    "CONTROLLER_UNITS",
    "set_keys",
    "GAIN_KEYS",
    "gain_array",
    "gain_points",
    "load_params",
    "default_params_path",
    "builtin_actuators",
    "bundled_actuators",
    "actuator_path",
    "ALIASES",
    "parse_set",
    "apply_sets",
]


# Domain of every key: "Ts" the sampling range TS_RANGE, ">0" strictly positive, ">=0" non-negative, "int>=1" integer >= 1,
# "filter" a registered velocity filter (haa_sym.model.filters). The plant's domains are per topology
# (haa_sym.model.actuator: inertias, couplings, L, R, k_t, N > 0; frictions, dampings, k_w and stiffness
# to ground >= 0). Ts sets the sampling, N_av the state dimension; alpha = 0 switches velocity
# compensation off (Fig. 9a). The velocity filters' keys (N_av, f_c) take their domains from the
# registry, which says which filter reads them (Controller checks).
_CONTROLLER_DOMAIN: dict[str, str] = {
    "Ts": "Ts", "N_av": FILTER_PARAMETERS["N_av"].domain, "alpha": ">=0", "beta": ">0", "P_t0": ">=0",
    "I_t0": ">=0", "velocity_filter": "filter", "f_c": FILTER_PARAMETERS["f_c"].domain,
    "structure": "structure",
}
# The velocity estimate is a modelling choice with a stated default (the paper's average); a
# filter's keys are optional in a file unless the chosen filter reads them without a default.
# The controller's structure likewise (haa_sym.model.structures, default the paper's); the keys a
# structure does not read (P_t0, I_t0, beta without a torque loop; alpha without velocity
# compensation) are left out of a file and take their neutral values (structures.NEUTRAL).
_CONTROLLER_OPTIONAL = {"velocity_filter": filters.DEFAULT, **{k: None for k in FILTER_PARAMETERS},
                        "structure": structures.DEFAULT, **{k: None for k in structures.NEUTRAL}}
STRING_KEYS = ("velocity_filter", "structure")   # keys whose value is a name, not a number
# The sampling times accepted, s: the maps' decisions are checked against the eigenvalues of the
# explicit closed loop from 10 us to 8 ms (docs/model.md); 1 us to 1 s leaves room on either side,
# and beyond it the closed-loop poles sit within rounding of z = 1 (Ts = 1e-300 gave "stable,
# spectral radius 1") or the sampled plant overflows.
TS_RANGE = (1e-6, 1.0)
_DOMAIN_TEXT = {
    "Ts": f"a sampling time from {TS_RANGE[0]:g} to {TS_RANGE[1]:g} s",
    ">0": "a finite number > 0",
    ">=0": "a finite number >= 0",
    "int>=1": "an integer >= 1",
}
# The largest integer a count (N_av) may take. The averaging filter is built as an exact
# polynomial of N_av + 1 coefficients before the loop checks its order against the generated
# capacity (N_av <= 56 with the bundled code), so an absurd N_av would first fill the memory;
# 10000 samples (10 s at 1 kHz) is far above any generated capacity and costs milliseconds.
INT_MAX = 10_000
# the largest parameter file read, bytes: the bundled ones are a few kilobytes; a path to a log or
# a disk image by mistake is refused with its size, not parsed
MAX_FILE_BYTES = 16 << 20
# Gain points of every analysis: the impedance gains of Eq. (8) and the torque-loop gains, whose
# rule is the controller file's (beta = 0 switches the torque PI off; negative gains are positive
# feedback, which the analysis, the paper and the generated sign conventions do not cover).
_GAIN_DOMAIN: dict[str, str] = {"P_gain": ">=0", "D_gain": ">=0",
                                "beta": _CONTROLLER_DOMAIN["beta"], "alpha": _CONTROLLER_DOMAIN["alpha"]}
_GAIN_UNITS = {"P_gain": " (Nm/rad)", "D_gain": " (Nms/rad)", "beta": "", "alpha": ""}
GAIN_KEYS: tuple[str, ...] = tuple(_GAIN_DOMAIN)

CONTROLLER_KEYS: tuple[str, ...] = tuple(_CONTROLLER_DOMAIN)


def domain_text(domain: str) -> str:
    """What a key's ``domain`` (">0", ">=0", "int>=1", "filter") allows, in words."""
    if domain == "structure":
        return structures.allowed_text()
    return filters.allowed_text() if domain == "filter" else _DOMAIN_TEXT[domain]


def set_keys(params: "Params") -> list[tuple[str, str, str, object]]:
    """Every key ``--set`` / :meth:`Params.with_values` accepts for ``params``:
    ``(key, unit, allowed, current value)``, the plant's (its topology's order) then the
    controller's, then the drive's."""
    top = params.plant.topology
    rows = [(k, top.units[k], domain_text(d), params.plant.as_dict()[k]) for k, d in top.domain.items()]
    unread = structures.get(params.controller.structure).unread
    rows += [(k, CONTROLLER_UNITS.get(k, "name"),
              f"not read by structure {params.controller.structure!r} (with --set structure=NAME that reads it)"
              if k in unread else domain_text(d), getattr(params.controller, k))
             for k, d in _CONTROLLER_DOMAIN.items()]
    rows += [(k, DRIVE_UNITS[k], drive_allowed(k), getattr(params.drive, k)) for k in DRIVE_KEYS]
    return rows


class Plant:
    """Physical parameters of one actuator, SI units, validated (Table 1 for HyQ).

    Values are read by their flat names (``plant.J_L2``, ``plant.K_hd``; see
    :class:`haa_sym.model.actuator.Topology`), the object is immutable, and :meth:`replace` validates
    like a file.

    Parameters
    ----------
    topology : Topology or LinearActuatorModel, optional
        The actuator (any :class:`haa_sym.model.actuator.Actuator`: a chain topology, or a sympy model
        written in code, :class:`haa_sym.symbolic.model.LinearActuatorModel`). Default: the HyQ
        HAA joint of the paper (:data:`haa_sym.model.actuator.HYQ`). Also readable as ``actuator``.
    **values : float
        Every key of ``topology.parameter_keys``, in the units of ``topology.units``.
    """

    __slots__ = ("topology", "_values")

    def __init__(self, topology: Topology | None = None, /, **values: float):
        topology = HYQ if topology is None else topology
        if not isinstance(topology, Actuator):
            raise ParameterError(f"topology = {topology!r}; allowed: a haa_sym.model.actuator.Topology or a "
                                 "haa_sym.symbolic.model.LinearActuatorModel")
        domain = topology.domain
        check_keys(values, tuple(domain), tuple(domain))
        checked = {k: _check_value(k, values[k], domain[k]) for k in domain}
        object.__setattr__(self, "topology", topology)
        object.__setattr__(self, "_values", checked)

    def __getattr__(self, name: str) -> float:
        try:
            return object.__getattribute__(self, "_values")[name]
        except KeyError:
            raise AttributeError(f"Plant has no parameter {name!r}") from None

    def __setattr__(self, name, value):
        raise AttributeError("Plant is immutable; use plant.replace(key=value)")

    def __eq__(self, other) -> bool:
        return (isinstance(other, Plant) and self.topology == other.topology
                and self.as_tuple() == other.as_tuple())

    def __hash__(self) -> int:
        return hash((self.topology, self.as_tuple()))

    def __repr__(self) -> str:
        return "Plant(" + ", ".join(f"{k}={v!r}" for k, v in self._values.items()) + ")"

    def __reduce__(self):
        return (_plant_from, (self.topology, self._values))

    @property
    def actuator(self) -> Actuator:
        """The actuator these values are for (the same object as ``topology``)."""
        return self.topology

    @property
    def keys(self) -> tuple[str, ...]:
        return self.topology.parameter_keys

    def as_dict(self) -> dict[str, float]:
        """Values by flat name, in ``topology.parameter_keys`` order."""
        return dict(self._values)

    def as_tuple(self) -> tuple[float, ...]:
        """Values in ``topology.parameter_keys`` order (the order the generated code expects)."""
        return tuple(self._values.values())

    def replace(self, **changes: float) -> "Plant":
        """A copy with some keys changed, validated like a file."""
        return Plant(self.topology, **{**self._values, **changes})


def _plant_from(topology, values):
    return Plant(topology, **values)


@dataclass(frozen=True)
class Controller:
    """Controller defaults of Sec. 3: sampling, velocity estimate, velocity compensation, PI gains.

    ``P_t = beta * P_t0`` and ``I_t = beta * I_t0`` (Eq. 7); the simplified velocity compensation
    gain is ``alpha * N / k_t * (R B_m + k_t k_w)`` (Eq. 6). The velocity estimate
    ``velocity_filter`` (default ``"average"``, the paper's) is one of the registry
    :mod:`haa_sym.model.filters`: ``"average"`` of ``N_av`` samples, or the backward difference followed
    by a Tustin ``"lowpass1"`` or ``"butterworth2"`` filter of cut-off ``f_c`` Hz (below Nyquist
    1/(2 Ts)), or any filter registered there. The keys the chosen filter reads are required (or
    take the registry's default); the others may be None. ``structure`` (default ``"paper"``) is
    an entry of :mod:`haa_sym.model.structures`: the keys it does not read (``P_t0``, ``I_t0``,
    ``beta`` without a torque loop, ``alpha`` without compensation) are refused if given and
    hold their neutral values (0, 0, 1, 0); ``alternatives`` holds other structures' keys
    (``[controller.<structure>]``) for a switch with ``--set structure=...``.
    """

    Ts: float
    N_av: int | None
    alpha: float | None = None
    beta: float | None = None
    P_t0: float | None = None
    I_t0: float | None = None
    velocity_filter: str = filters.DEFAULT
    f_c: float | None = None
    structure: str = structures.DEFAULT
    # the keys of other structures for this actuator ([controller.<structure>] tables): what
    # `--set structure=<name>` takes when it switches to one (not part of the loop: no equality)
    alternatives: Mapping[str, Mapping[str, float]] = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self):
        st = structures.get(_check_value("structure", self.structure, "structure"))
        for k in st.unread:             # a key the structure does not read: left out, neutral
            if self.__dict__[k] is not None and self.__dict__[k] != structures.NEUTRAL[k]:
                raise ParameterError(f"{k} = {self.__dict__[k]!r}: structure = {st.name!r} has no "
                                     f"{'torque PI' if k != 'alpha' else 'velocity compensation'}; allowed: "
                                     f"leave {k} out (it reads {list(st.keys) or 'none of P_t0, I_t0, beta, alpha'})")
            object.__setattr__(self, k, structures.NEUTRAL[k])
        _check_fields(self, {k: d for k, d in _CONTROLLER_DOMAIN.items()
                             if not (k in FILTER_PARAMETERS and getattr(self, k) is None)})
        kind = self.velocity_filter
        nyquist = 0.5 / self.Ts
        for p in filters.get(kind).parameters:          # the keys the chosen filter reads
            value = getattr(self, p.name)
            if value is None and p.default is not None:
                value = _check_value(p.name, p.default, p.domain)
                object.__setattr__(self, p.name, value)
            if value is None:
                allowed = (f"a {p.description} in {p.units}, 0 < {p.name} < {nyquist:g} (Nyquist)"
                           if p.below_nyquist else _DOMAIN_TEXT[p.domain])
                raise ParameterError(f"{p.name} is missing; allowed: {allowed}, required by "
                                     f"velocity_filter = {kind!r}")
            if p.below_nyquist and not value < nyquist:
                raise ParameterError(f"{p.name} = {value!r} is at or above Nyquist 1/(2 Ts) = {nyquist:g} "
                                     f"{p.units}; allowed: 0 < {p.name} < {nyquist:g} ({p.units})")

    @property
    def P_t(self) -> float:
        return self.beta * self.P_t0

    @property
    def I_t(self) -> float:
        return self.beta * self.I_t0

    def replace(self, **changes: float) -> "Controller":
        """A copy with some keys changed, validated like a file. A change of ``structure`` drops
        the keys the new structure does not read; those it reads and this one did not must be
        among ``changes``."""
        values = {k: v for k, v in {**self.__dict__, **changes}.items() if k != "alternatives"}
        new = structures.get(_check_value("structure", values["structure"], "structure"))
        old = structures.get(self.structure)
        alternatives = dict(self.alternatives)
        if new is not old:                  # the keys of the one left, for a switch back
            alternatives.setdefault(old.name, {k: getattr(self, k) for k in old.keys})
        for k in structures.NEUTRAL:
            if k not in changes and (k in new.unread or k in old.unread):
                values.pop(k)               # neutral in the new one, or missing (reported as such)
                if k in new.keys and k in alternatives.get(new.name, {}):
                    values[k] = alternatives[new.name][k]     # the file's [controller.<structure>]
        return _controller(values, alternatives=alternatives)


@dataclass(frozen=True)
class Params:
    """A validated parameter file: nominal plant (of its topology), controller and named leg
    configurations; ``about`` is the file's [about] table (name, description, references)."""

    plant: Plant
    controller: Controller
    configurations: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    source: str = "<memory>"
    about: Mapping[str, object] = field(default_factory=dict, compare=False)
    # the nonlinear simulation's limits ([limits], haa_sym.model.limits); the linear analyses
    # ignore them, so they take no part in equality (nor in the memos keyed by Params)
    limits: Limits = field(default_factory=Limits, compare=False)
    # [motor] convention (haa_sym.model.actuator.MOTOR_CONVENTIONS): how k_t and k_w are compared
    # for the plausibility warning only; the model uses both values as given
    motor_convention: str = field(default=MOTOR_CONVENTION_DEFAULT, compare=False)
    # the drive between command and motor ([drive], haa_sym.model.drive): it changes the sampled
    # plant, so it takes part in equality and in every memo keyed by Params
    drive: Drive = field(default_factory=Drive)

    def __post_init__(self):
        if not isinstance(self.plant, Plant):
            raise ParameterError(f"{self.source}: plant = {self.plant!r}; allowed: a haa_sym.Plant")
        if not isinstance(self.controller, Controller):
            raise ParameterError(f"{self.source}: controller = {self.controller!r}; allowed: a haa_sym.Controller")
        if not isinstance(self.drive, Drive):
            raise ParameterError(f"{self.source}: drive = {self.drive!r}; allowed: a haa_sym.model.drive.Drive")
        if not isinstance(self.configurations, Mapping):
            raise ParameterError(f"{self.source}: [configurations] must be a table of tables")
        configs = {}
        for name, overrides in self.configurations.items():
            where = f"{self.source} [configurations.{name}]"
            if not isinstance(overrides, Mapping):
                raise ParameterError(f"{where}: must be a table of plant keys")
            domain = self.plant.topology.domain
            unknown = sorted(set(overrides) - set(domain))
            if unknown:
                raise ParameterError(f"{where}: unknown key(s) {unknown}; allowed: {list(domain)}")
            configs[name] = {k: _check_value(k, v, domain[k], where) for k, v in overrides.items()}
        object.__setattr__(self, "configurations", configs)

    @classmethod
    def from_model(cls, model: Actuator, values: Mapping[str, float],
                   controller: "Controller | Mapping[str, object]", *,
                   configurations: Mapping[str, Mapping[str, float]] | None = None,
                   source: str | None = None) -> "Params":
        """Parameters of an actuator defined in code (what :func:`load_params` reads from a file).

        Parameters
        ----------
        model : LinearActuatorModel or Topology
            The actuator: a sympy model (:class:`haa_sym.symbolic.model.LinearActuatorModel`) or
            a chain (:class:`haa_sym.model.actuator.Topology`).
        values : mapping str -> float
            Every key of ``model.parameter_keys``, SI units (``model.units``), checked against
            ``model.domain``.
        controller : Controller or mapping
            A :class:`Controller`, or its keys as in a file's ``[controller]`` table (``Ts`` in s,
            ``N_av``, ``alpha``, ``beta``, ``P_t0`` in V/Nm, ``I_t0`` in V/(Nm s), optional
            ``velocity_filter`` and ``f_c`` in Hz).
        configurations : mapping, optional
            Name -> plant keys to override (as ``[configurations.<name>]``).
        source : str, optional
            How messages name these parameters; default ``model.source``.

        Returns
        -------
        Params

        Raises
        ------
        ParameterError
            Naming the source, ``values`` or ``controller``, the key and what is allowed.
        """
        if not isinstance(model, Actuator):
            raise ParameterError(f"model = {model!r}; allowed: a haa_sym.symbolic.model.LinearActuatorModel "
                                 "or a haa_sym.Topology")
        source = model.source if source is None else source
        if not isinstance(values, Mapping):
            raise ParameterError(f"{source} values: {values!r}; allowed: a mapping of {list(model.parameter_keys)}")
        try:
            plant = Plant(model, **values)
        except ParameterError as exc:
            raise ParameterError(f"{source} values: {exc}") from None
        if not isinstance(controller, Controller):
            if not isinstance(controller, Mapping):
                raise ParameterError(f"{source} controller: {controller!r}; allowed: a haa_sym.Controller "
                                     f"or a mapping of {list(CONTROLLER_KEYS)}")
            controller = _controller(controller, f"{source} controller")
        return cls(plant=plant, controller=controller, configurations=dict(configurations or {}),
                   source=source)

    def configuration(self, name: str) -> "Params":
        """The parameters with the plant overrides of configuration ``name`` applied."""
        if name not in self.configurations:
            raise ParameterError(
                f"{self.source}: unknown configuration {name!r}; "
                f"allowed: {sorted(self.configurations) or 'none defined'}"
            )
        return replace(self, plant=self.plant.replace(**self.configurations[name]))

    def with_values(self, **changes: float) -> "Params":
        """A copy with any plant, controller or drive keys changed (what ``--set KEY=VALUE`` does)."""
        keys = self.plant.topology.parameter_keys
        plant_changes = {k: v for k, v in changes.items() if k in keys}
        ctrl_changes = {k: v for k, v in changes.items() if k in _CONTROLLER_DOMAIN}
        drive_changes = {k: v for k, v in changes.items() if k in DRIVE_KEYS}
        unknown = sorted(set(changes) - set(plant_changes) - set(ctrl_changes) - set(drive_changes))
        if unknown:
            raise ParameterError(
                f"unknown parameter key(s) {unknown}; allowed: {list(keys + CONTROLLER_KEYS + DRIVE_KEYS)}"
            )
        return replace(
            self,
            plant=self.plant.replace(**plant_changes) if plant_changes else self.plant,
            controller=self.controller.replace(**ctrl_changes) if ctrl_changes else self.controller,
            drive=self.drive.replace(**drive_changes) if drive_changes else self.drive,
        )

    def to_dict(self) -> dict:
        """Plain values, for saving next to results (with the topology: self-describing)."""
        top = self.plant.topology
        return {
            "plant": self.plant.as_dict(),
            "topology": {**top.structure(), "fingerprint": top.fingerprint},
            "controller": {k: v for k, v in self.controller.__dict__.items()
                           if not (k == "alternatives" and not v)},
            "configurations": {k: dict(v) for k, v in self.configurations.items()},
            "drive": self.drive.as_dict(),
            "source": self.source,
        }


def builtin_actuators(directory: str | Path | None = None) -> list[Path]:
    """The bundled actuator files: every ``model/*.toml`` except ``paper.toml`` (the paper's
    reported results), sorted by name; their plant functions are generated (``make derive``)."""
    d = Path(directory) if directory is not None else data_dir("model")
    return sorted(p for p in d.glob("*.toml") if p.name != "paper.toml")


# Short names of bundled actuators (alias -> the file's stem). "hyq" is how the paper and the
# README call the robot; the file is named after the joint (HAA) because other HyQ joints differ.
ALIASES: dict[str, str] = {"hyq": "hyq_haa"}


def bundled_actuators() -> dict[str, Path]:
    """The bundled actuators by name: ``{stem: path}`` of :func:`builtin_actuators` (``haptic_wall``,
    ``harmonic_drive``, ``hyq_haa``, ``qdd_leg``, ``sea``), in the source tree or inside the installed package."""
    return {p.stem: p for p in builtin_actuators()}


def actuator_path(name_or_path: str | Path | None = None, field: str | None = None) -> Path:
    """The parameter file meant by ``name_or_path``: an existing path (a file always wins), else
    a bundled actuator's name (:func:`bundled_actuators`) or alias (:data:`ALIASES`); None is
    the bundled HyQ file.

    Raises
    ------
    ParameterError
        Naming ``field`` (e.g. ``--params``), the value and the bundled names, when it is neither.
    """
    if name_or_path is None:
        return default_params_path()
    p = Path(name_or_path)
    if p.exists():
        return p
    bundled = bundled_actuators()
    name = ALIASES.get(str(name_or_path), str(name_or_path))
    if name in bundled:
        return bundled[name]
    label = f"{field} {str(name_or_path)!r}" if field else repr(str(name_or_path))
    names = list(bundled) + [f"{a} (= {n})" for a, n in ALIASES.items()]
    raise ParameterError(f"{label}: no such parameter file, nor a bundled actuator; allowed: a TOML "
                         f"file or a bundled name: {', '.join(names)} (haa-sym actuators lists them)")


def default_params_path() -> Path:
    """``model/hyq_haa.toml``, the bundled HyQ parameters (source tree or installed package)."""
    return data_dir("model") / "hyq_haa.toml"


# the number domains besides "int>=1" (its messages are its own) as bounds of check_number
_BOUNDS = {">0": dict(low=0.0, low_open=True), ">=0": dict(low=0.0), "Ts": dict(low=TS_RANGE[0], high=TS_RANGE[1])}


def _check_value(key: str, value: object, domain: str, where: str | None = None) -> float | int:
    """``value`` of ``key`` checked against ``domain``; the message names where, key, value, allowed."""
    prefix = f"{where}: " if where else ""
    if domain == "filter":
        if value not in filters.names():
            raise ParameterError(f"{prefix}{key} = {value!r}; allowed: {filters.allowed_text()}")
        return value
    if domain == "structure":
        if not (isinstance(value, str) and value in structures.STRUCTURES):
            raise ParameterError(f"{prefix}{key} = {value!r}; allowed: {structures.allowed_text()} "
                                 "(docs/model.md, \"Controller structures\")")
        return value
    allowed = _DOMAIN_TEXT[domain]
    if value is None:
        raise ParameterError(f"{prefix}{key} = None is missing; allowed: {allowed}")
    if domain != "int>=1":
        return check_number(key, value, allowed, where, **_BOUNDS[domain])
    if isinstance(value, int) and not isinstance(value, bool):
        # a Python int is exact at any size: a huge one is out of range, not "not finite" or
        # "not an integer" (its float would be)
        if not 1 <= value <= INT_MAX:
            raise ParameterError(f"{prefix}{key} = {value!r} is out of range; allowed: {allowed}"
                                 + (f" and <= {INT_MAX}" if value > INT_MAX else ""))
        return value
    check_number(key, value, allowed, where)            # a finite number (a float here)
    if not float(value).is_integer():
        raise ParameterError(f"{prefix}{key} = {value!r} is not an integer; allowed: {allowed}")
    if not 1 <= value <= INT_MAX:
        raise ParameterError(f"{prefix}{key} = {value!r} is out of range; allowed: {allowed}"
                             + (f" and <= {INT_MAX}" if value > INT_MAX else ""))
    return int(value)


def _check_fields(obj, domain: Mapping[str, str]) -> None:
    """Validate and normalise (float, or int for N_av) every field of a frozen dataclass."""
    for key, dom in domain.items():
        object.__setattr__(obj, key, _check_value(key, getattr(obj, key), dom))


def _validated(cls, values: Mapping[str, object], domain: Mapping[str, str], where: str | None = None,
               optional: Mapping[str, object] = {}):
    prefix = f"{where}: " if where else ""
    check_keys(values, tuple(domain), [k for k in domain if k not in optional], where)
    values = {**{k: v for k, v in optional.items() if k not in values}, **values}
    try:
        return cls(**values)
    except ParameterError as exc:
        raise ParameterError(f"{prefix}{exc}") from None


def _controller(values: Mapping[str, object], where: str | None = None, alternatives=None) -> Controller:
    """A :class:`Controller` from a [controller] table's values: the keys its ``structure``
    (haa_sym.model.structures) reads are required, those it does not read are refused if given;
    ``alternatives`` the other structures' keys (:func:`_alternatives`)."""
    prefix = f"{where}: " if where else ""
    name = values.get("structure", structures.DEFAULT)
    st = structures.get(_check_value("structure", name, "structure", where))
    given = [k for k in st.unread if k in values]
    if given:
        raise ParameterError(f"{prefix}{given[0]} = {values[given[0]]!r}: structure = {st.name!r} has no "
                             f"{'velocity compensation' if given[0] == 'alpha' else 'torque PI'}; allowed: "
                             f"leave {', '.join(given)} out (it reads {list(st.keys) or 'none of P_t0, I_t0, beta, alpha'})")
    ctrl = _validated(Controller, values, _CONTROLLER_DOMAIN, where,
                      optional={k: v for k, v in _CONTROLLER_OPTIONAL.items() if k not in st.keys})
    object.__setattr__(ctrl, "alternatives", dict(alternatives or {}))
    return ctrl


def _alternatives(table: Mapping[str, object], source: str, refs) -> tuple[dict, dict]:
    """``([controller] without its sub-tables, {structure: its keys})``: a ``[controller.<name>]``
    table, ``<name>`` a structure of haa_sym.model.structures other than the file's, holds exactly
    the keys that structure reads, for ``--set structure=<name>``."""
    own = table.get("structure", structures.DEFAULT)
    rest, alts = {}, {}
    for name, tab in table.items():
        if name not in structures.STRUCTURES:
            rest[name] = tab
            continue
        where = f"{source} [controller.{name}]"
        if not isinstance(tab, Mapping):
            raise ParameterError(f"{where}: {tab!r}; allowed: a table of the keys structure {name!r} reads")
        if name == own:
            raise ParameterError(f"{where}: the file's own structure; allowed: its keys in [controller] itself")
        st = structures.STRUCTURES[name]
        vals = entry_values(tab, where, refs, CONTROLLER_UNITS)
        check_keys(vals, st.keys, st.keys, where)
        alts[name] = {k: _check_value(k, v, _CONTROLLER_DOMAIN[k], where) for k, v in vals.items()}
    return rest, alts


def gain_array(name: str, value, label: str | None = None) -> np.ndarray:
    """``value`` as a float array, checked against the rule of gain ``name``.

    The one rule for the gain points of every analysis (CLI and API): ``P_gain`` >= 0 (Nm/rad)
    and ``D_gain`` >= 0 (Nms/rad) of Eq. (8), ``beta`` > 0 and ``alpha`` >= 0 of Eq. (6)-(7),
    all finite. Any other ``name`` (e.g. ``omega``) is only required to be finite.

    Parameters
    ----------
    name : str
        One of :data:`GAIN_KEYS`, or another array name.
    value : array_like
    label : str, optional
        How the message names the value (e.g. ``--P-gain``); default ``name``.

    Raises
    ------
    ParameterError
        Naming the label, the first offending value and what is allowed.
    """
    label = label or name
    domain = _GAIN_DOMAIN.get(name)
    allowed = (_DOMAIN_TEXT[domain] + _GAIN_UNITS[name]) if domain else "finite numbers"
    try:
        raw = np.asarray(value)
    except (TypeError, ValueError):                 # e.g. ragged nested lists
        raise ParameterError(f"{label} = {value!r} is not a number; allowed: {allowed}") from None
    items = raw.ravel().tolist() if raw.dtype == object else []
    if any(v is None for v in items):
        # a float conversion would turn None into nan and report "nan is not finite"
        where = f"{label} = None" if raw.ndim == 0 else f"{label} contains None, which"
        raise ParameterError(f"{where} is missing; allowed: {allowed}")
    if np.iscomplexobj(raw) or any(isinstance(v, complex) for v in items):
        # numpy would drop the imaginary part with a ComplexWarning; a gain is real
        cands = [complex(v) for v in raw.ravel().tolist() if isinstance(v, complex)]
        first = next((c for c in cands if c.imag), cands[0])
        where = f"{label} = {first!r}" if raw.ndim == 0 else f"{label} contains {first!r}, which"
        raise ParameterError(f"{where} is complex; allowed: real values, {allowed}")
    try:
        arr = np.asarray(raw, dtype=float)
    except (TypeError, ValueError):
        raise ParameterError(f"{label} = {value!r} is not a number; allowed: {allowed}") from None
    with np.errstate(invalid="ignore"):
        bad = ~np.isfinite(arr)
        if domain == ">0":
            bad |= ~(arr > 0)
        elif domain == ">=0":
            bad |= ~(arr >= 0)
    if bad.any():
        first = float(arr[bad].ravel()[0])
        what = "is not finite" if not math.isfinite(first) else "is out of range"
        where = f"{label} = {first!r}" if arr.ndim == 0 else f"{label} contains {first!r}, which"
        raise ParameterError(f"{where} {what}; allowed: {allowed}")
    return arr


def gain_points(P_gain=0.0, D_gain=0.0, beta=None, alpha=None):
    """Gain points checked by :func:`gain_array`: ``(P_gain, D_gain, beta, alpha)`` as arrays,
    P_gain and D_gain broadcast together; a beta or alpha of None stays None (the controller's)."""
    P, D = gain_array("P_gain", P_gain), gain_array("D_gain", D_gain)
    try:
        P, D = np.broadcast_arrays(P, D)
    except ValueError:
        raise ParameterError(f"P_gain has shape {P.shape} and D_gain {D.shape}; allowed: shapes that "
                             "broadcast together (one value each per gain point)") from None
    return (P, D, None if beta is None else gain_array("beta", beta),
            None if alpha is None else gain_array("alpha", alpha))


_FILE_SECTIONS = ACTUATOR_SECTIONS + ("controller", "configurations", "limits", "drive")
_LEGACY_SECTIONS = ("about", "plant", "controller", "configurations", "limits")


def parse_params(data: Mapping[str, object], source: str = "<memory>") -> Params:
    """Validate the content of a parameter file already read into a mapping.

    The actuator sections ([about], [motor], [bodies.*], [couplings.*], [sensors]; or the legacy
    flat [plant]) are read by :func:`haa_sym.model.actuator.parse_actuator`; [controller] and
    [configurations.*] here.
    """
    legacy = "plant" in data
    allowed = _LEGACY_SECTIONS if legacy else _FILE_SECTIONS
    top = sorted(set(data) - set(allowed))
    if top:
        hint = " (a file with [plant] is the legacy HyQ format: no [motor], [bodies], [couplings], " \
               "[sensors])" if legacy else ""
        raise ParameterError(f"{source}: unknown table(s) {top}; allowed: {list(allowed)}{hint}")
    data, convention = split_convention(data, source)
    topology, raw, about = parse_actuator(data, source)
    values = {}
    for key, dom in topology.domain.items():
        section, local = ("plant", key) if legacy else topology.section_of(key)
        values[key] = _check_value(local, raw[key], dom, f"{source} [{section}]")
    plant = Plant(topology, **values)
    if not isinstance(data.get("controller"), Mapping):
        raise ParameterError(f"{source}: missing table [controller]")
    refs = about["references"]
    table, alternatives = _alternatives(data["controller"], source, refs)
    controller = _controller(entry_values(table, f"{source} [controller]", refs,
                                                     {**CONTROLLER_UNITS, "velocity_filter": None,
                                                      "structure": None}),
                            f"{source} [controller]", alternatives)
    raw_configs = data.get("configurations", {})
    if not isinstance(raw_configs, Mapping):
        raise ParameterError(f"{source}: [configurations] must be a table of tables")
    configs = {}
    for name, overrides in raw_configs.items():
        where = f"{source} [configurations.{name}]"
        if not isinstance(overrides, Mapping):
            raise ParameterError(f"{where}: must be a table of plant keys")
        configs[name] = entry_values(overrides, where, refs, topology.units)
    limits = parse_limits(data["limits"], topology.body_names, source, refs) if "limits" in data else Limits()
    drive = parse_drive(data["drive"], source, refs) if "drive" in data else Drive()
    return Params(plant=plant, controller=controller, configurations=configs, source=source, about=about,
                  limits=limits, motor_convention=convention, drive=drive)


def _read_toml(raw: bytes) -> dict:
    """``tomllib.load`` with the cyclic garbage collector paused: tomllib recurses once per
    nesting level, and a collection that starts deep in a file nested thousands of levels runs
    other objects' finalizers at the recursion limit, where they fail and Python prints
    "Exception ignored in ..." to stderr beside the one-line error (seen once in CI, in
    tests/test_cli_faults.py::test_deeply_nested_toml)."""
    paused = gc.isenabled()
    gc.disable()
    try:
        return tomllib.loads(raw.decode("utf-8"))
    finally:
        if paused:
            gc.enable()


def load_params(path: str | Path | None = None) -> Params:
    """Read and validate a parameter file.

    Parameters
    ----------
    path : str, os.PathLike or None
        TOML file, or the name of a bundled actuator (``"hyq_haa"`` or ``"hyq"``, ``"sea"``,
        ``"harmonic_drive"``, ``"qdd_leg"``, ``"haptic_wall"``; :func:`actuator_path`: an existing file wins);
        default the bundled ``model/hyq_haa.toml``. Anything else is a :class:`ParameterError`.

    Returns
    -------
    Params

    Raises
    ------
    ParameterError
        Naming the file, the key, the offending value and what is allowed.
    """
    if path is not None and not isinstance(path, (str, os.PathLike)):
        raise ParameterError(f"load_params: path = {path!r} ({type(path).__name__}); allowed: a file path "
                             "(str or os.PathLike), a bundled actuator's name or None (the bundled "
                             "model/hyq_haa.toml)")
    p = actuator_path(path)
    if not Path(p).exists():
        raise ParameterError(f"{p}: no such parameter file")
    raw = read_bytes(p, "parameter file", limit=MAX_FILE_BYTES, where=str(p))
    try:
        data = _read_toml(raw)
    except tomllib.TOMLDecodeError as exc:
        raise ParameterError(f"{p}: not valid TOML ({exc}); allowed: a TOML parameter file") from None
    except RecursionError:
        # tomllib parses nested arrays and inline tables recursively: thousands of levels
        # exhaust Python's stack
        raise ParameterError(f"{p}: not a parameter file (arrays or tables nested too deeply for the "
                             "TOML parser); allowed: a TOML parameter file") from None
    except UnicodeDecodeError as exc:
        raise ParameterError(f"{p}: not a text file (byte 0x{exc.object[exc.start]:02x} at offset "
                             f"{exc.start} is not UTF-8); allowed: a TOML parameter file") from None
    return parse_params(data, source=str(p))


def parse_set(items: list[str], known: tuple[str, ...] | None = None) -> dict[str, float | int | str]:
    """``KEY=VALUE`` texts (``--set``, the explorer's fields) as values: a number (an integer
    stays one, so that messages show the value as typed: N_av = 0, not 0.0) or, for
    :data:`STRING_KEYS`, the name. ``known``: the keys allowed (an unknown key with a non-number
    value is reported as the key's mistake). The one parser of the CLI and the explorer."""
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep:
            raise ParameterError(f"--set {item!r}: expected KEY=VALUE")
        key, value = key.strip(), value.strip()
        if key in STRING_KEYS:          # a choice by name (velocity_filter), checked by Controller
            out[key] = value
            continue
        try:
            out[key] = int(value) if value.lstrip("+-").isdigit() else float(value)
        except ValueError:
            if known is not None and key not in known:    # the key is the mistake, not the value
                raise ParameterError(f"--set {key}={value}: unknown parameter key(s) {[key]}; "
                                     f"allowed: {list(known)}") from None
            raise ParameterError(f"--set {key}={value}: {value!r} is not a number; allowed: a finite "
                                 "number") from None
    return out


def apply_sets(params: Params, sets: Mapping[str, object]) -> Params:
    """``params`` with ``sets`` (from :func:`parse_set`) applied all at once (velocity_filter and
    its keys, e.g. f_c, are only valid together); a refusal names the ``--set`` items at fault."""
    if not sets:
        return params
    try:
        return params.with_values(**sets)
    except ParameterError as exc:
        msg = str(exc)
        named = [k for k in sets if msg.startswith((f"{k} ", f"unknown parameter key(s) ['{k}'"))]
        given = " ".join(f"--set {k}={v}" for k, v in sets.items() if not named or k in named)
        raise ParameterError(f"{given}: {msg}") from None
