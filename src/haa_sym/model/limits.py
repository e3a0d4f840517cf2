"""The optional ``[limits]`` section of an actuator file: what the linear model leaves out.

Every entry is written like the others (``{ value, unit, source, description }``, a bare number
is SI) and converted by :func:`haa_sym.model.units.to_si`. An absent key is an absent limit.

=====================  ==========  ========================================================
key                    SI unit     what
=====================  ==========  ========================================================
``V_max``              V           supply voltage: the held command is clipped to +-V_max
``I_max``              A           drive current limit (a voltage window, docs/simulate.md)
``Fc_m``               Nm          Coulomb friction torque of the rotor
``Fc_<body>``          Nm          Coulomb friction torque of body ``<body>`` (a [bodies] name)
``encoder_counts``     \\-          encoder counts per revolution of the encoder body
``torque_resolution``  Nm          quantum of the torque signal the loop reads
``torque_noise``       Nm          rms of white Gaussian noise on that signal
``jitter``             s           rms of the sample instants' offsets from k Ts
``friction_velocity``  rad/s       velocity scale v_s of the smooth friction model
``friction_model``     (a name)    ``"tanh"`` (the default): T = -Fc tanh(v / v_s)
=====================  ==========  ========================================================

Example
-------
>>> lim = parse_limits({"V_max": {"value": 48, "unit": "V"}, "Fc_L1": 0.5}, ("L1", "L2"), "f.toml")
>>> lim.V_max, lim.friction, lim.friction_velocity
(48.0, {'L1': 0.5}, 0.01)
>>> parse_limits({"Fc_L3": 0.5}, ("L1", "L2"), "f.toml")
Traceback (most recent call last):
...
haa_sym.errors.ParameterError: f.toml [limits]: unknown key(s) ['Fc_L3']; allowed: ['V_max', 'I_max', 'Fc_m', 'Fc_L1', 'Fc_L2', 'encoder_counts', 'torque_resolution', 'torque_noise', 'jitter', 'friction_velocity', 'friction_model']
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Mapping

from haa_sym.errors import ParameterError
from haa_sym.model.actuator import check_keys, entry_values
from haa_sym.model.units import check_number

__all__ = ["Limits", "FRICTION_MODELS", "DEFAULT_FRICTION_MODEL", "DEFAULT_FRICTION_VELOCITY",
           "limit_units", "parse_limits", "FRICTION_SET_KEYS", "with_friction_sets"]

#: The friction models: "tanh" (smooth, the default). "stick-slip" (exact sticking) is named so
#: that a file asking for it gets a clear refusal: it is not implemented (docs/simulate.md).
FRICTION_MODELS = ("tanh",)
DEFAULT_FRICTION_MODEL = "tanh"
#: v_s of the smooth model (rad/s at the body the friction acts on): below it the friction is a
#: steep viscous slope Fc / v_s instead of a stick; 0.01 rad/s keeps that slope within a few
#: integrator substeps per millisecond for the bundled drives (docs/simulate.md).
DEFAULT_FRICTION_VELOCITY = 0.01

# key -> (SI unit, domain, text of what is allowed)
_FIXED = {
    "V_max": ("V", ">0", "a number > 0 (V)"),
    "I_max": ("A", ">0", "a number > 0 (A)"),
    "encoder_counts": ("-", "int>=1", "an integer >= 1 (counts per revolution)"),
    "torque_resolution": ("Nm", ">=0", "a number >= 0 (Nm; 0 = not quantised)"),
    "torque_noise": ("Nm", ">=0", "a number >= 0 (Nm rms)"),
    "jitter": ("s", ">=0", "a number >= 0 (s rms)"),
    "friction_velocity": ("rad/s", ">0", "a number > 0 (rad/s)"),
}
_FRICTION = ("Nm", ">=0", "a number >= 0 (Nm)")


@dataclass(frozen=True)
class Limits:
    """The limits of one actuator, SI; None (or an empty ``friction``) is off.

    ``friction`` maps ``"m"`` (the rotor) and body names to Coulomb torques (Nm).
    """

    V_max: float | None = None
    I_max: float | None = None
    friction: Mapping[str, float] = field(default_factory=dict)
    encoder_counts: int | None = None
    torque_resolution: float | None = None
    torque_noise: float | None = None
    jitter: float | None = None
    friction_velocity: float = DEFAULT_FRICTION_VELOCITY
    friction_model: str = DEFAULT_FRICTION_MODEL

    @property
    def active(self) -> dict:
        """The limits that are on, by key (for provenance and reports)."""
        out = {k: getattr(self, k) for k in ("V_max", "I_max", "encoder_counts", "torque_resolution",
                                             "torque_noise", "jitter") if getattr(self, k)}
        out.update({f"Fc_{b}": v for b, v in self.friction.items() if v})
        if any(self.friction.values()):
            out.update(friction_model=self.friction_model, friction_velocity=self.friction_velocity)
        return out


def limit_units(bodies) -> dict[str, str | None]:
    """Key -> SI unit of every ``[limits]`` key for an actuator with these body names."""
    units = {k: u for k, (u, _d, _a) in _FIXED.items()}
    fr = {"Fc_m": "Nm", **{f"Fc_{b}": "Nm" for b in bodies}}
    keys = ["V_max", "I_max", *fr, "encoder_counts", "torque_resolution", "torque_noise", "jitter",
            "friction_velocity", "friction_model"]
    return {k: ({**units, **fr}.get(k)) for k in keys}


# the domains of _FIXED and _FRICTION as bounds of check_number
_BOUNDS = {">0": dict(low=0.0, low_open=True), ">=0": dict(low=0.0), "int>=1": dict(low=1, integer=True)}


def _check(key, value, domain, allowed, where):
    return check_number(key, value, allowed, where, **_BOUNDS[domain])


def parse_limits(table: object, bodies, source: str = "<memory>",
                 references: Mapping[str, str] | None = None) -> Limits:
    """Validate a ``[limits]`` table; ``bodies`` are the actuator's body names.

    Raises
    ------
    ParameterError
        One line naming the file, ``[limits]``, the key, the value and what is allowed.
    """
    where = f"{source} [limits]"
    if not isinstance(table, Mapping):
        raise ParameterError(f"{where}: [limits] = {table!r}; allowed: a table of limit entries")
    units = limit_units(bodies)
    check_keys(table, tuple(units), (), where)
    values = entry_values(table, where, references, units)
    out: dict[str, object] = {}
    friction = {}
    for k, v in values.items():
        if k == "friction_model":
            if v == "stick-slip":
                raise ParameterError(f"{where}: friction_model = 'stick-slip' is not implemented; "
                                     f"allowed: {list(FRICTION_MODELS)} (docs/simulate.md)")
            if v not in FRICTION_MODELS:
                raise ParameterError(f"{where}: friction_model = {v!r}; allowed: {list(FRICTION_MODELS)}")
            out[k] = v
        elif k.startswith("Fc_"):
            friction[k[3:]] = _check(k, v, *_FRICTION[1:], where)
        else:
            out[k] = _check(k, v, *_FIXED[k][1:], where)
    return Limits(friction=friction, **out)


#: The [limits] keys ``--set`` may change besides the ``Fc_<entry>`` torques (identify's friction).
FRICTION_SET_KEYS = ("friction_velocity",)


def with_friction_sets(limits: Limits, sets: Mapping[str, object], bodies) -> Limits:
    """``limits`` with ``Fc_m`` / ``Fc_<body>`` (Nm, >= 0) and ``friction_velocity`` (rad/s, > 0)
    from ``sets`` (``--set KEY=VALUE``, SI), checked as a file's ``[limits]`` entries are.

    Raises
    ------
    ParameterError
        An ``Fc_`` key that is not the rotor's or a body's, or a value out of its domain; one line
        naming ``--set KEY=VALUE``.
    """
    friction, out = dict(limits.friction), {}
    allowed = ["Fc_m"] + [f"Fc_{b}" for b in bodies]
    for k, v in sets.items():
        where = f"--set {k}={v}"
        if k.startswith("Fc_"):
            if k not in allowed:
                raise ParameterError(f"{where}: not a friction entry; allowed: {allowed}")
            friction[k[3:]] = _check(k, v, *_FRICTION[1:], where)
        elif k in FRICTION_SET_KEYS:
            out[k] = _check(k, v, *_FIXED[k][1:], where)
        else:
            raise ParameterError(f"{where}: not a [limits] friction key; allowed: {allowed + list(FRICTION_SET_KEYS)}")
    return replace(limits, friction=friction, **out)
